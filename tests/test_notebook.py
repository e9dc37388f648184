"""docs/examples/grid.ipynb runs from top to bottom (nbclient, a fresh kernel) and draws its recall curves."""

from pathlib import Path

import pytest

nbclient = pytest.importorskip("nbclient", reason="nbclient is in the dev extra")
nbformat = pytest.importorskip("nbformat")
pytest.importorskip("ipykernel", reason="ipykernel is in the dev extra")

NOTEBOOK = Path(__file__).resolve().parents[1] / "docs" / "examples" / "grid.ipynb"


def test_the_example_notebook_runs_a_grid_and_plots_its_recall_curves(tmp_path):
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": tmp_path}}
    ).execute()
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs]
    assert not [out for out in outputs if out.output_type == "error"]
    assert sum("image/png" in out.get("data", {}) for out in outputs) == 1  # the recall curves
    printed = "".join(out.get("text", "") for out in outputs if out.output_type == "stream")
    assert (
        "9 records in runs/synthetic-test" in printed
    )  # 3 combinations x 3 frames, stored under the notebook's folder
