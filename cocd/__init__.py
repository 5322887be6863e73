"""cocd: rigid granular media with hard Coulomb contact, one convex conic problem per step.

The data flow is one way::

    Scene -> ContactSet -> ConicProblem -> solvers.solve -> Solution -> Stepper -> records
"""

from cocd.builders import box_3d, column_2d, stack
from cocd.contacts import ContactSet, contact_jacobian, detect_contacts
from cocd.errors import (
    CocdError,
    OverlapError,
    ProblemError,
    SceneError,
    SolverError,
    SolverNotFound,
)
from cocd.measure import kinetic_energy, potential_energy
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
    "CocdError",
    "ConicProblem",
    "ContactSet",
    "OverlapError",
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
    "box_3d",
    "ccp_residual",
    "column_2d",
    "contact_jacobian",
    "coulomb_residual",
    "detect_contacts",
    "dynamics_residual",
    "kinetic_energy",
    "potential_energy",
    "project_coulomb",
    "residuals",
    "stack",
]
