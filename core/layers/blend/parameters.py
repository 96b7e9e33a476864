"""The blend layer's parameter kinds (see ``core.parameters``):

    ``blend:<pose>``   weight of an expression-library pose, in % (0 = rest, 100 = the pose;
                       −50 … 200 allows reducing and exaggerating)
    ``caricature``     exaggeration of the face's difference from the library's mean face, in %
                       (−100 = the mean face, 0 = the face, 200 = three times as distinctive)

Pose names are the library's (lower-case words, ``core.layers.blend.library.POSE_NAME``); which
poses a face has depends on its library, so any well-formed name is a valid key and the rig says
when its face has no such pose. The layer is registered for rigs that meet these keys (a project,
a timeline track): it starts with the built-in library when there is one for the face.
"""

from __future__ import annotations

from core.layer import register_layer
from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, register_kind, split_words

WEIGHT_RANGE = (-50.0, 200.0)        # % of a pose's displacement
CARICATURE_RANGE = (-100.0, 200.0)   # % exaggeration


def _blend_key(args: list[str]) -> ParamKey:
    from core.layers.blend.library import POSE_NAME

    (word,) = split_words(args, 1, "blend keys are 'blend:<pose>' with a pose of the face's expression library, "
                                   "e.g. 'blend:joy'")
    word = word.lower()
    if not POSE_NAME.match(word):
        raise ParameterError(f"blend:{word}: pose names are lower-case words (letters, digits, '_'), e.g. 'blend:joy'")
    if word == "neutral":
        raise ParameterError("'blend:neutral' is the rest face itself: set the other blend weights to 0 instead")
    return ParamKey("blend", word)


def _blend_describe(key: ParamKey) -> Parameter:
    lo, hi = WEIGHT_RANGE
    return Parameter(str(key), key.id.replace("_", " "), "%", lo, hi, 0.0, "blends",
                     description=f"Adds the scanned pose '{key.id}' from the expression library: 100 % is the "
                                 "pose, 0 % the neutral face; beyond 100 % exaggerates it.")


def _caricature_key(args: list[str]) -> ParamKey:
    if args:
        raise ParameterError("the caricature key is just 'caricature' (exaggeration in %)")
    return ParamKey("caricature")


def _caricature_describe(key: ParamKey) -> Parameter:
    lo, hi = CARICATURE_RANGE
    return Parameter("caricature", "caricature", "%", lo, hi, 0.0, "blends",
                     description="Scales the face's difference from the mean face: −100 % is the mean face, "
                                 "0 % the face itself, positive values exaggerate it.")


def _layer_for(rig):
    from core.layers.blend.layer import BlendLayer

    return BlendLayer.for_rig(rig)


register_kind(ParameterKind("blend", "blend:<pose>", _blend_key, _blend_describe, order=7))
register_kind(ParameterKind("caricature", "caricature", _caricature_key, _caricature_describe, order=8))
register_layer("blend", ("blend", "caricature"), _layer_for)

__all__ = ["WEIGHT_RANGE", "CARICATURE_RANGE"]
