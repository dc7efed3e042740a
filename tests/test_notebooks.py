"""Every notebook in notebooks/ runs top to bottom on the CPU (small settings); ours open in Colab."""

import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))
COLAB = "https://colab.research.google.com/github/jdpim/jdpim/blob/main/notebooks/"
WITH_BADGE = ("accuracy", "design", "impact_damper", "paper", "pounding", "quickstart", "reliability", "sensitivities")


def execute(path, workdir):
    """Run one notebook top to bottom in a fresh kernel whose working directory is ``workdir``."""
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}).execute()
    return nb


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
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
