"""Measurements: pure functions of a scene's state or of a recorded run.

These are the quantities read off a granular collapse (Martin et al. 2022,
sections 4-5): energies, the front position ``r_f`` and the runout, the mass
(free-surface) profile ``h(x)``, the volume occupied by the mass and its
relative variation ``a_V``, velocity profiles ``u_x(z)`` at a station, the
static/flowing interface ``h_sf`` and the erodible bed's energy ratio.

Conventions
-----------
- Frame: the flow direction is the coordinate ``axis`` (default 0, x); the last
  coordinate is z, normal to the plane (a slope is a tilted gravity, so z is the
  height above the plane, as in the field's profiles); in 3D the remaining
  coordinate is y, across the channel.
- State: functions take a :class:`~cocd.scene.Scene` or arrays: positions
  ``(n, d)``, radii ``(n,)`` or one number, velocities ``(n, d)``. Given a Scene,
  glued (fixed) grains are left out unless ``mask`` says otherwise: a glued layer
  spans the whole plane and would join every grain into one mass.
- Units: SI. In 2D a "volume" is an area (m^2, i.e. m^3 per metre of depth) and
  energies are per metre of depth.
- Bins are edges, strictly increasing; a grain belongs to the bin holding its
  centre, ``[e_k, e_k+1)`` (the last bin also holds its right edge); grains
  outside every bin are ignored.
"""

from __future__ import annotations

from cocd.measure._common import DEFAULT_GAP_FRACTION, STATIC_VELOCITY, MassProfile
from cocd.measure.energy import bed_energy_ratio, kinetic_energy, potential_energy
from cocd.measure.flow import static_flowing_interface, velocity_profile
from cocd.measure.front import (
    bed_surface,
    bed_top,
    front_position,
    main_mass,
    relative_runout,
    runout,
    surface_front,
)
from cocd.measure.profile import granular_volume, mass_profile, relative_volume_variation

__all__ = [
    "DEFAULT_GAP_FRACTION",
    "STATIC_VELOCITY",
    "MassProfile",
    "bed_energy_ratio",
    "bed_surface",
    "bed_top",
    "front_position",
    "granular_volume",
    "kinetic_energy",
    "main_mass",
    "mass_profile",
    "potential_energy",
    "relative_runout",
    "relative_volume_variation",
    "runout",
    "static_flowing_interface",
    "surface_front",
    "velocity_profile",
]
