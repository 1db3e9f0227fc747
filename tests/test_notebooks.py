"""Every notebook runs top to bottom on a clean kernel, with small settings put into its parameters cell."""

import time
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
SMALL = {
    "01_thesis_chapter4.ipynb": "T_END = 2.0",
    "02_thesis_chapter5.ipynb": "N_ANGLES = 7",
    "03_board_level_drop.ipynb": "N_MODES_MAX = 4\nN_AMPLIFICATION = 5",
    "04_monte_carlo.ipynb": "N = 4000\nN_FLAT = 200\nLIMIT = 2500e-6",
    "05_placement.ipynb": "STEPS = 4\nSTARTS = 1",
    "06_speed_vs_accuracy.ipynb": "RERUN = False",
    "07_clatter_and_campaigns.ipynb": "N_ANGLES = 7\nMAX_IMPACTS = 3\nWRITE_FIGURES = False",
    "08_plates_and_mounts.ipynb": "BASIS = (8, 6)\nEDGES = (\"FFFF + 4 screws\",)\nSTEPS = 2\nSTARTS = 1",
    "10_landings.ipynb": "N_ANGLES = 1\nWRITE_FIGURES = False\nBOARDS = (\"beam (default phone)\",)",
    "11_box_drops.ipynb": "N_TILTS = 3\nWRITE_FIGURES = False",
    "09_validation.ipynb": "N_THETA = 41\nFE_ELEMENTS = (20, 40)\nFE_STEPS_US = (4.0, 2.0)\nPLATE_MESHES_MM = (8.0,)\n"
                           "PLATE_STEPS_US = (20.0,)\nFINE_BASIS = (12, 12)",
}


def test_every_notebook_is_covered():
    assert {p.name for p in NOTEBOOKS.glob("*.ipynb")} == set(SMALL)


@pytest.mark.parametrize("name", sorted(SMALL))
def test_notebook_runs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    params = [c for c in nb.cells if "parameters" in c.metadata.get("tags", [])]
    assert len(params) == 1, "each notebook has one cell tagged 'parameters'"
    params[0].source = SMALL[name]
    start = time.perf_counter()
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    # Figures were drawn and tables printed.
    kinds = {k for c in nb.cells if c.cell_type == "code" for o in c.outputs for k in o.get("data", {})}
    assert "image/png" in kinds and "text/markdown" in kinds
    print(f"{name}: {time.perf_counter() - start:.1f} s")
