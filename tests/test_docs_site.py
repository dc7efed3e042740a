"""The documentation site builds in strict mode (broken links, missing references and docstring errors fail it);
the benchmark records carry their metadata and the README quotes them; the version is pyproject's."""

import json
import os
import pathlib
import re
import runpy
import subprocess
import sys

import jdpim

ROOT = pathlib.Path(__file__).parents[1]


def _nav_pages(nav) -> list[str]:
    """The files a mkdocs ``nav`` names, in order."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [p for v in nav.values() for p in _nav_pages(v)]
    return [p for item in nav for p in _nav_pages(item)]


def test_site_builds_strict_without_warnings(tmp_path):
    import yaml

    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log
    assert "WARNING -" not in log, log
    with open(ROOT / "mkdocs.yml") as f:
        nav = _nav_pages(yaml.safe_load(f)["nav"])
    for page in nav:  # every page of the nav is built
        built = tmp_path / "site" / ("index.html" if page == "index.md" else f"{page.rsplit('.', 1)[0]}/index.html")
        assert built.is_file(), page
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    for name in ("jdpim.Scene", "jdpim.solve", "jdpim.Result", "jdpim.first_passage", "jdpim.sensitivity"):
        assert f'id="{name}"' in api, name  # the reference is generated from the docstrings


def test_every_committed_record_carries_date_machine_versions_load_and_protocol():
    records = sorted((ROOT / "docs" / "bench").glob("*.json"))
    assert records
    for path in records:
        rec = json.loads(path.read_text())["record"]
        assert set(rec) >= {"date", "machine", "versions", "load_average", "protocol"}, path.name
        assert set(rec["machine"]) >= {"cpu", "cores"} and set(rec["versions"]) >= {"python", "jax", "jdpim"}, path.name
        md = path.with_suffix(".md")
        assert not md.exists() or f"Measured {rec['date']}" in md.read_text(), md.name


def test_version_is_pyproject_version_in_the_package_and_the_citation():
    if sys.version_info >= (3, 11):
        import tomllib
    else:
        import tomli as tomllib
    import yaml

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert jdpim.__version__ == declared
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert str(citation["version"]) == declared
    assert [r["year"] for r in citation["references"]] == [2019, 2016, 2016]  # DPIM, GF-discrepancy, random functions


def test_readme_command_entry_point(capsys):
    # `python3 -m jdpim paper --quick`: the module runs the command line as a program, and only then
    proc = subprocess.run(
        [sys.executable, "-m", "jdpim", "paper", "-h"], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert proc.returncode == 0 and "--quick" in proc.stdout, proc.stderr
    runpy.run_module("jdpim.__main__", run_name="jdpim.__main__")  # its code run as an import (here: no new process)
    assert capsys.readouterr() == ("", "")  # importing it runs nothing


def _record_values() -> list[float]:
    """Every number in the committed records (JSON values, and the numbers of the accuracy CSV)."""
    values = []

    def walk(obj):
        if isinstance(obj, dict | list):
            for v in obj.values() if isinstance(obj, dict) else obj:
                walk(v)
        elif isinstance(obj, int | float) and not isinstance(obj, bool):
            values.append(float(obj))

    for path in (ROOT / "docs" / "bench").glob("*.json"):
        walk(json.loads(path.read_text()))
    for line in (ROOT / "docs" / "bench" / "accuracy.csv").read_text().splitlines()[1:]:
        values += [float(x) for x in line.split(",")[2:]]
    return values


def test_readme_headline_numbers_are_the_records():
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Headline results") : text.index("## Documentation")]
    values = _record_values()
    quoted = re.findall(r"(?<![\w.\-])\d+\.\d+(?:e-?\d+)?", section)
    assert len(quoted) >= 8
    for token in quoted:  # each decimal number is a record's value at the precision quoted
        mantissa, _, exponent = token.partition("e")
        digits = len(mantissa.split(".")[1])
        if exponent:
            assert any(f"{v:.{digits}e}" == f"{float(token):.{digits}e}" for v in values), token
        else:
            assert any(round(v, digits) == float(token) for v in values), token
