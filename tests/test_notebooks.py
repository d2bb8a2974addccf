"""The notebooks' code cells run top to bottom (a smoke test so they do not rot)."""

import itertools
import json
from pathlib import Path

import matplotlib
import pytest

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("LUNAR_DRAKE_CACHE", str(tmp_path / "cache"))
    nb = json.loads(path.read_text())
    src = "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code")
    # IPython display is not available under pytest; show file names instead.
    src = src.replace(
        "from IPython.display import Image\n", "def Image(filename): return filename\n"
    )
    exec(compile(src, str(path), "exec"), {"__name__": "__notebook__"})


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_explains_each_step_and_has_a_kernel(path):
    """Every code cell follows a prose (markdown) cell; the set-up installed a Jupyter
    kernel (ipykernel) for it; library code never forces a matplotlib backend (that
    would kill inline plots)."""
    import importlib.util

    cells = json.loads(path.read_text())["cells"]
    assert cells and cells[0]["cell_type"] == "markdown"
    for before, cell in itertools.pairwise(cells):
        if cell["cell_type"] == "code":
            assert before["cell_type"] == "markdown" and "".join(before["source"]).strip()
    assert importlib.util.find_spec("ipykernel") is not None
    library = Path(__file__).parent.parent / "lunar_drake"
    offenders = [p for p in library.rglob("*.py") if "matplotlib.use(" in p.read_text()]
    assert offenders == []
