"""cocd: rigid granular media with hard Coulomb contact, one convex conic problem per step.

The data flow is one way::

    Scene -> ContactSet -> ConicProblem -> solvers.solve -> Solution -> Stepper -> records
"""

from cocd.builders import HARD_CASES, box_3d, column_2d, column_collapse, stack, static_box
from cocd.contacts import ContactSet, Penetration, contact_jacobian, detect_contacts, penetration
from cocd.errors import (
    CocdError,
    OverlapError,
    PenetrationError,
    PenetrationWarning,
    ProblemError,
    SceneError,
    SolverError,
    SolverNotFound,
)
from cocd.measure import (
    MassProfile,
    bed_energy_ratio,
    front_position,
    granular_volume,
    kinetic_energy,
    main_mass,
    mass_profile,
    potential_energy,
    relative_runout,
    relative_volume_variation,
    runout,
    static_flowing_interface,
    velocity_profile,
)
from cocd.packing import rain_deposition
from cocd.problem import ConicProblem, PrimalConicForm, assemble
from cocd.residuals import (
    Residuals,
    ccp_residual,
    coulomb_residual,
    dynamics_residual,
    project_coulomb,
    residuals,
)
from cocd.scene import Scene, Wall
from cocd.stepper import Stepper, StepRecord

__version__ = "0.1.0"

__all__ = [
    "HARD_CASES",
    "CocdError",
    "ConicProblem",
    "ContactSet",
    "MassProfile",
    "OverlapError",
    "Penetration",
    "PenetrationError",
    "PenetrationWarning",
    "PrimalConicForm",
    "ProblemError",
    "Residuals",
    "Scene",
    "SceneError",
    "SolverError",
    "SolverNotFound",
    "StepRecord",
    "Stepper",
    "Wall",
    "assemble",
    "bed_energy_ratio",
    "box_3d",
    "ccp_residual",
    "column_2d",
    "column_collapse",
    "contact_jacobian",
    "coulomb_residual",
    "detect_contacts",
    "dynamics_residual",
    "front_position",
    "granular_volume",
    "kinetic_energy",
    "main_mass",
    "mass_profile",
    "penetration",
    "potential_energy",
    "project_coulomb",
    "rain_deposition",
    "relative_runout",
    "relative_volume_variation",
    "residuals",
    "runout",
    "stack",
    "static_box",
    "static_flowing_interface",
    "velocity_profile",
]
