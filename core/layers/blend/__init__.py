"""Expression blends (thesis A ch. 4): displacement sets of registered scans, interpolation,
transfer between faces, caricatures, and FAP correctives.

- ``library``: :class:`ExpressionLibrary` (rest, poses, displacements), rigid alignment, building;
- ``transfer``: thesis bounding-box scaling (eqs. 4.4–4.6) and deformation transfer;
- ``caricature``: mean face and exaggeration;
- ``corrective``: FAP least-squares fit of a scan and the residual as a FAP-driven corrective;
- ``layer``: :class:`BlendLayer`, the rig layer (keys ``blend:<pose>`` and ``caricature``);
- ``scans``: a person's expression scans → landmarks → registration → library, with a per-scan summary;
- ``builtin``: the default face's built-in library and its builder (``python -m core.layers.blend.builtin``);
- ``parameters``: the parameter kinds; files: ``core.formats.blend_library``.
"""
