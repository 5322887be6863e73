"""The seed's Table 1: its cases, sizes, tolerances and reference rows, and the table's
columns."""

from __future__ import annotations

from typing import Any

#: Phases of a step's solve in the time breakdown (``t_<phase>_s``): the backend's
#: set-up, and for ``ipm`` the assembly of the reduced system, its numerical
#: factorisations, the triangular solves, the residual checks and the polish;
#: ``other`` is the rest of the wall time (for most backends: all their iterations).
PHASES = ("setup", "assemble", "factor", "solve", "check", "polish", "other")

#: Columns of ``table1.csv``, in order.
COLUMNS = [
    "source",
    "case",
    "dim",
    "N",
    "Nc",
    "Nc_per_grain",
    "d_max_r",
    "dt",
    "tol",
    "solver",
    "start",
    "steps_ok",
    "iterations",
    "wall_s",
    "ccp_residual",
    "coulomb_residual",
    "factorisations",
    *(f"t_{phase}_s" for phase in PHASES),
    "scale",
    "note",
]

THIS_MACHINE = "this machine"
SEED = "seed (Mosek, 2x8 cores)"
CASE_2D = "variation of N"
CASE_3D = "variation of mu"

#: Disc counts of the seed's "variation of N" (its Fig. 5 and Table 1).
SEED_N_2D = [1109, 8308, 20488, 50772]
#: Sphere count of the seed's "variation of mu".
SEED_N_3D = 122932
#: Below this the column is too small to flow like a granular column.
MIN_GRAINS = 20
DT_2D, DT_3D = 1e-3, 1e-2
EPS_2D = [1e-8]
EPS_3D = [1e-8, 1e-5]
MU_3D = 0.3
CHANNEL_WIDTH = 0.2
TRAJECTORY_TOL = 1e-8
#: Tolerance of the 3D trajectory's steps before the first recorded one (the 2D
#: ones use TRAJECTORY_TOL): 100 steps of a flowing column at 1e-8 take longer
#: than every backend's solves together.
PREP_TOL_3D = 1e-6

#: Detection thresholds D of the two cases, in mean radii: the fixed thresholds at
#: which the columns have the seed's potential contacts per grain at the start of
#: the recorded steps (4.49 per disc for 8308 discs, 6.75 per sphere), measured on
#: the 8308-disc column and the 1229-sphere one (1 % of the seed's)
#: (``cocd bench seed-contacts``, ``results/seed_contacts.md``).
D_SEED_2D = 1.63
D_SEED_3D = 0.98

#: Table 1 of the seed (DESIGN.md section 5): Mosek's interior point, cold, ten steps.
SEED_ROWS: list[dict[str, Any]] = [
    dict(case=CASE_2D, dim=2, N=8308, Nc=37331, dt=DT_2D, tol=1e-8, iterations=47, time=8.85),
    dict(case=CASE_2D, dim=2, N=50772, Nc=238659, dt=DT_2D, tol=1e-8, iterations=61, time=51.9),
    dict(case=CASE_3D, dim=3, N=122932, Nc=829505, dt=DT_3D, tol=1e-8, iterations=21, time=475.8),
    dict(case=CASE_3D, dim=3, N=122932, Nc=829505, dt=DT_3D, tol=1e-5, iterations=11, time=269.9),
]
