"""mkdocs hooks: the docstrings' Sphinx roles (``:class:`X```) rendered as code, linked where the page has X."""

import re

ROLE = re.compile(r":(?:class|func|meth|attr|mod|data):(<code>([^<]*)</code>)")


def on_page_content(html, page, config, files):
    """Drop the role prefix; link the name to its entry on the same page (``jdpim.X`` or ``X`` by its full id)."""

    def replace(match):
        code, name = match.group(1), match.group(2).lstrip("~.")
        for anchor in (name, f"jdpim.{name}"):
            if f'id="{anchor}"' in html:
                return f'<a href="#{anchor}">{code}</a>'
        return code

    return ROLE.sub(replace, html)
