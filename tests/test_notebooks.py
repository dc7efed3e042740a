"""Every notebook in notebooks/ runs top to bottom on the CPU (small settings); ours open in Colab.

Every notebook's code is checked against the library in the default tier: its cells parse, every jdpim name it uses
exists, and every call of a jdpim function or class binds to its signature. Running a notebook costs its own process
and its own programs (15 to 60 CPU-s each): the default tier runs the quickstart and the paper's reproduction
(``jdpim.paper.reproduce``, which no other test runs), and the ``slow`` tier (``-m slow``) runs the others, whose
computations the default tier checks in the tests named in ``SLOW``.
"""

import ast
import importlib
import inspect
import pathlib
import re

import nbformat
import pytest
from nbclient import NotebookClient

import jdpim

NOTEBOOKS = sorted((pathlib.Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))
# notebooks run only in the slow tier, each with the default-tier tests that check what it computes
SLOW = {
    "accuracy": "test_bench_accuracy",
    "design": "test_design",
    "impact_damper": "test_mdof, test_scenefile_mdof",
    "pounding": "test_pounding, test_fragility",
    "reliability": "test_first_passage_pi::test_elastic_linear_exact_bounds, test_first_passage",
    "sensitivities": "test_gradients, test_sensitivity_estimators",
}
COLAB = "https://colab.research.google.com/github/jdpim/jdpim/blob/main/notebooks/"
WITH_BADGE = ("accuracy", "design", "impact_damper", "paper", "pounding", "quickstart", "reliability", "sensitivities")


def execute(path, workdir):
    """Run one notebook top to bottom in a fresh kernel whose working directory is ``workdir``."""
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}).execute()
    return nb


def _code(path) -> str:
    """A notebook's code cells as one module, IPython's magics (``%pip ...``) commented out."""
    cells = [c.source for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code"]
    return "\n".join(re.sub(r"^(\s*)%", r"\1# %", cell, flags=re.M) for cell in cells)


def _imported(tree) -> dict:
    """The names a notebook binds to jdpim or its modules (``import jdpim.paper``, ``from jdpim import figures``)."""
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "jdpim":
                    module = importlib.import_module(alias.name)
                    names[alias.asname or "jdpim"] = module if alias.asname else jdpim
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "jdpim":
            module = importlib.import_module(node.module)
            for alias in node.names:
                names[alias.asname or alias.name] = _member(module, alias.name, f"{node.module}.{alias.name}")
    return names


def _member(obj, name: str, dotted: str):
    if not hasattr(obj, name) and inspect.ismodule(obj):
        try:
            importlib.import_module(f"{obj.__name__}.{name}")  # a submodule not imported by its package
        except ModuleNotFoundError:
            pass
    assert hasattr(obj, name), f"{dotted} does not exist"
    return getattr(obj, name)


def _resolve(node, names: dict):
    """The object of an attribute chain rooted at a jdpim name (``jdpim.bench.accuracy.sweep``), else None."""
    chain = []
    while isinstance(node, ast.Attribute):
        chain.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name) or node.id not in names:
        return None
    obj, dotted = names[node.id], node.id
    for attr in reversed(chain):
        dotted += f".{attr}"
        obj = _member(obj, attr, dotted)
    return obj


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_code_uses_the_library_as_it_is(path):
    """Every jdpim name a notebook uses exists, and every call of a jdpim callable binds its positional and keyword
    arguments to the callable's signature (a renamed or removed function, class, module or argument fails here)."""
    tree = ast.parse(_code(path), filename=str(path))
    names = _imported(tree)
    assert "jdpim" in names, "the notebook imports jdpim"
    calls = 0
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            _resolve(node, names)
        elif isinstance(node, ast.Call):
            target = _resolve(node.func, names) if isinstance(node.func, ast.Attribute) else None
            if isinstance(node.func, ast.Name) and node.func.id in names:
                target = names[node.func.id]
            starred = any(isinstance(a, ast.Starred) for a in node.args) or any(k.arg is None for k in node.keywords)
            if target is None or not callable(target) or starred:
                continue
            try:
                signature = inspect.signature(target)
            except (TypeError, ValueError):  # a builtin without a signature
                continue
            try:
                signature.bind(*node.args, **{k.arg: k.value for k in node.keywords})
            except TypeError as e:
                raise AssertionError(f"line {node.lineno}: {ast.unparse(node.func)}(...) {e}") from None
            calls += 1
    assert calls > 0


@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in NOTEBOOKS],
    ids=[p.stem for p in NOTEBOOKS],
)
def test_notebook_runs(path, notebook_runs):
    # the notebooks run one after another in a background process (conftest.py): this waits for its result
    nb = notebook_runs[path.stem].result()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


@pytest.mark.parametrize("name", WITH_BADGE)
def test_notebook_opens_in_colab_with_outputs_committed(name):
    nb = nbformat.read(pathlib.Path(__file__).parents[1] / "notebooks" / f"{name}.ipynb", as_version=4)
    assert f"({COLAB}{name}.ipynb)" in nb.cells[0].source and "Open in Colab" in nb.cells[0].source
    install = nb.cells[1]
    assert install.cell_type == "code" and "except ImportError" in install.source and "pip install" in install.source
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count is not None for c in code), "commit the notebook executed"
    assert sum(bool(c.outputs) for c in code) >= 2
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
