"""Every figure the package draws. Functions take results, draw on an optional `ax`, and return the figure."""

from .box import plot_box as plot_box
from .drop import (
    plot_deflected_board as plot_deflected_board,
    plot_flat_landing as plot_flat_landing,
    plot_gauge_history as plot_gauge_history,
    plot_housing_impact as plot_housing_impact,
    plot_impact as plot_impact,
    plot_impacts as plot_impacts,
    plot_landing as plot_landing,
    plot_plate_strain as plot_plate_strain,
    plot_scene as plot_scene,
    plot_sensitivity as plot_sensitivity,
    plot_stress_map as plot_stress_map,
)
from .studies import (
    plot_bench as plot_bench,
    plot_campaign as plot_campaign,
    plot_montecarlo as plot_montecarlo,
    plot_placement as plot_placement,
    plot_stability as plot_stability,
)
