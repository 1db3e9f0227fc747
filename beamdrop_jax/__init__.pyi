"""The public names of beamdrop_jax. The package imports each private module on first use of one of its names
(`lazy_loader` reads this file), so `import beamdrop_jax` costs little more than importing JAX."""

from ._common.checks import Flag as Flag, GRAVITY as GRAVITY, IMPULSE_DURATION as IMPULSE_DURATION
from ._board.base import AbstractBoard as AbstractBoard, AbstractModal as AbstractModal
from ._board.beam import Board as Board
from ._scene.containers import (
    Contact as Contact,
    Drop as Drop,
    Housing as Housing,
    Placement as Placement,
    Scene as Scene,
    board_ends as board_ends,
    check_scene as check_scene,
    scene_flags as scene_flags,
)
from ._scene.file import embedded_scenes as embedded_scenes, load_scene as load_scene, save_scene as save_scene
from ._impact.routh import ImpactMode as ImpactMode, ImpactResult as ImpactResult, routh_impulse as routh_impulse
from ._impact.impulse3d import Impact3D as Impact3D, impulse_3d as impulse_3d
from ._impact.box import (
    BoxImpact as BoxImpact,
    LowestVertex as LowestVertex,
    box_attitude as box_attitude,
    box_impact as box_impact,
    box_inertia as box_inertia,
    box_vertices as box_vertices,
    lowest_vertex as lowest_vertex,
    rigid_vertex_impact as rigid_vertex_impact,
    vertex_contact_matrix as vertex_contact_matrix,
)
from ._impact.kinematics import (
    HousingImpact as HousingImpact,
    approach_velocity as approach_velocity,
    body_axes as body_axes,
    contact_matrix as contact_matrix,
    corner_impact as corner_impact,
    housing_impact as housing_impact,
    lowest_corner as lowest_corner,
    support_jumps as support_jumps,
)
from ._impact.clatter import (
    Ending as Ending,
    Impacts as Impacts,
    corner_heights as corner_heights,
    impact_sequence as impact_sequence,
    next_contact as next_contact,
)
from ._impact.landing import Landing as Landing
from ._impact.box_landing import BoxLanding as BoxLanding, compliant_landing as compliant_landing
from ._impact.motion import HalfSine as HalfSine, Impulse as Impulse, PulseTrain as PulseTrain, Record as Record
from ._impact.motion import LandingMotion as LandingMotion
from ._response.landing_path import LandingHistories as LandingHistories, landing_histories as landing_histories
from ._impact.motion import JESD22_B111_CONDITION_B as JESD22_B111_CONDITION_B
from ._board.beam import ENDS as ENDS
from ._board.base import natural_frequencies as natural_frequencies
from ._studies.mounts import MountResult as MountResult, optimize_mounts as optimize_mounts
from ._board.plate import EDGE_CODES as EDGE_CODES, Plate as Plate, PlateModes as PlateModes, plate_modes as plate_modes
from ._response.pulses import unit_response as unit_response
from ._board.search import FieldPeak as FieldPeak
from ._response.results import (
    Fields as Fields,
    Response as Response,
    StrainMap as StrainMap,
)
from ._board.base import (
    Gauges as Gauges,
    Peak as Peak,
)
from ._response.numerics import (
    Numerics as Numerics,
)
from ._response.simulate import (
    board_response as board_response,
    drop_motion as drop_motion,
    simulate as simulate,
)
from ._response.objectives import (
    peak_deflection as peak_deflection,
    peak_strain as peak_strain,
    peak_stress as peak_stress,
)
from ._response.fields import (
    plate_strain_map as plate_strain_map,
    response_fields as response_fields,
    response_notes as response_notes,
    sample_notes as sample_notes,
)
from ._response.setup import (
    support_motion as support_motion,
)
from ._studies.placement import (
    PlacementResult as PlacementResult,
    drop_set as drop_set,
    optimize_placement as optimize_placement,
    placement_landscape as placement_landscape,
    placement_from_unconstrained as placement_from_unconstrained,
    placement_objective as placement_objective,
    risk as risk,
)
from ._response.superposition import (
    PlateTable as PlateTable,
    SuperpositionTable as SuperpositionTable,
    superposition_table as superposition_table,
    table_numerics as table_numerics,
    table_peaks as table_peaks,
)
from ._studies.distribution import DropDistribution as DropDistribution
from ._studies.montecarlo import (
    MonteCarloResult as MonteCarloResult,
    OrientationTable as OrientationTable,
    forget_tables as forget_tables,
    montecarlo as montecarlo,
    montecarlo_numerics as montecarlo_numerics,
    orientation_table as orientation_table,
    wilson_interval as wilson_interval,
)
from ._studies.sensitivity import (
    Sensitivity as Sensitivity,
    scalar_fields as scalar_fields,
    sensitivities as sensitivities,
    smooth_peak_stress as smooth_peak_stress,
)
from ._studies.standards import STANDARDS as STANDARDS, CampaignDrop as CampaignDrop, campaign_drops as campaign_drops
from ._studies.campaign import CampaignResult as CampaignResult, campaign as campaign
from ._peers.opensees import (
    FEResponse as FEResponse,
    PlateFEResponse as PlateFEResponse,
    opensees_board_response as opensees_board_response,
    opensees_plate_response as opensees_plate_response,
)
from ._peers.numpy_scipy import numpy_peak_stress as numpy_peak_stress
from ._bench import run_bench as run_bench, stability_study as stability_study
from ._plots import (
    plot_deflected_board as plot_deflected_board,
    plot_bench as plot_bench,
    plot_box as plot_box,
    plot_campaign as plot_campaign,
    plot_impact as plot_impact,
    plot_flat_landing as plot_flat_landing,
    plot_gauge_history as plot_gauge_history,
    plot_housing_impact as plot_housing_impact,
    plot_impacts as plot_impacts,
    plot_landing as plot_landing,
    plot_scene as plot_scene,
    plot_sensitivity as plot_sensitivity,
    plot_montecarlo as plot_montecarlo,
    plot_placement as plot_placement,
    plot_plate_strain as plot_plate_strain,
    plot_stability as plot_stability,
    plot_stress_map as plot_stress_map,
)
