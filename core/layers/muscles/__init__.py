"""Biomechanical muscle model (thesis C "SABiom": Lee-Terzopoulos-Waters 1995 + Lucero-Munhall 1999).

Model / State / Control split:

- ``model.TissueModel``   built once per face: skin (the dense MPEG-4 template), fascia and bone
  layers, springs, prisms, masses, jaw weights, binding to the full face (static data);
- ``muscles.MuscleSet``   the 19 muscles (resources/muscles/muscles.json) placed on the model;
- ``solver.TissueSolver`` forces, the quasi-static solve, the stable and the explicit integrators
  acting on a ``solver.State`` (positions, velocities, activations);
- ``layer.MuscleLayer``   the controls (19 forces + jaw), the rig layer and the public API;
- ``force_file``          ForceSet, thesis presets, JSON force files.
"""

from core.layers.muscles.force_file import (ForceFileError, ForceSet, load_force_set, preset, preset_names,
                         save_force_set)
from core.layers.muscles.layer import LayerSnapshot, MuscleLayer
from core.layers.muscles.model import MuscleModelError
from core.layers.muscles.muscles import MuscleSpec, control_keys, jaw_range, muscle_specs
from core.layers.muscles.solver import RelaxReport, SolverDiverged

__all__ = [
    "MuscleSpec", "muscle_specs", "control_keys", "jaw_range", "MuscleLayer", "LayerSnapshot", "ForceSet",
    "preset_names", "preset", "load_force_set", "save_force_set", "ForceFileError", "SolverDiverged",
    "RelaxReport", "MuscleModelError",
]
