"""The built-in default face: a procedural human head whose front is shaped like a single-view range scan.

``load_default_face()`` reads the committed copy in ``resources/default_face``
(fast); ``generate_face(params)`` builds any identity from scratch. Both give
the full head; ``full_head=False`` gives the front of the face only (the
scan-like surface the synthetic database and the registration protocol use).
Regenerate the committed copy with ``python -m core.default_face``.
"""

from core.default_face.params import FaceLayout, FaceParameters
from core.default_face.store import default_face_path, load_default_face, save_default_face

# The generator (and the scipy.interpolate / optimize / ndimage it needs, ~0.5 s to import) loads
# when one of these names is first read: the window's start-up only reads the committed copy.
_GENERATOR_NAMES = ("GRID_SPACING", "TEXTURE_SIZE", "feature_point_layout", "generate_face")


def __getattr__(name: str):
    if name in _GENERATOR_NAMES:
        from core.default_face import build

        return getattr(build, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "FaceLayout", "FaceParameters", "generate_face", "feature_point_layout", "load_default_face",
    "save_default_face", "default_face_path", "GRID_SPACING", "TEXTURE_SIZE",
]
