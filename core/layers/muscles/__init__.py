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

import importlib

# Names resolved on first use (PEP 562): the window's muscle dock lists the presets at start-up
# without importing the solver (numba, ~0.3 s) before the face is on screen.
_MODULE_OF = {
    "ForceFileError": "force_file", "ForceSet": "force_file", "load_force_set": "force_file",
    "preset": "force_file", "preset_id": "force_file", "preset_names": "force_file", "save_force_set": "force_file",
    "LayerSnapshot": "layer", "MuscleLayer": "layer", "MuscleModelError": "model",
    "MuscleSpec": "specs", "control_keys": "specs", "jaw_range": "specs", "muscle_specs": "specs",
    "RelaxReport": "solver", "SolverDiverged": "solver",
}


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "MuscleSpec", "muscle_specs", "control_keys", "jaw_range", "MuscleLayer", "LayerSnapshot", "ForceSet",
    "preset_names", "preset", "preset_id", "load_force_set", "save_force_set", "ForceFileError", "SolverDiverged",
    "RelaxReport", "MuscleModelError",
]
