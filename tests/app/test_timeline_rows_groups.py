"""Timeline rows are grouped by what they animate: control points, Waters muscles and blends each get
their own group (they were all filed under "Muscles")."""

from app.timeline_rows import GROUP_TITLES, group_of, group_order


def test_every_layer_kind_has_its_own_timeline_group():
    assert group_of("fap:3") == "jaw & chin"
    assert group_of("expression:joy") == "expressions" and group_of("viseme:3") == "visemes"
    assert group_of("muscle:risorius:left") == "muscles" and group_of("jaw") == "muscles"
    assert group_of("cp:8.3:x") == "control points"
    assert group_of("waters:zygomatic_major:left") == "waters"
    assert group_of("blend:joy") == "blends" and group_of("caricature") == "blends"
    assert group_of("someday:new") == "layers"
    groups = {group_of(k) for k in ("cp:8.3:x", "waters:a:left", "blend:joy", "someday:x", "jaw")}
    assert groups <= set(group_order()) and all(g in GROUP_TITLES for g in groups)


def test_show_all_lists_the_other_layers_the_face_has():
    from types import SimpleNamespace

    from app.timeline_rows import all_parameters

    rig = SimpleNamespace(animated_faps=(3,), parameters=lambda: ("fap:3", "cp:8.3:x", "waters:zygomatic_major:left",
                                                                   "blend:joy", "expression:joy"))
    controller = SimpleNamespace(rig=rig, document=SimpleNamespace(muscle_layer=None))
    keys = all_parameters(controller)
    assert {"cp:8.3:x", "waters:zygomatic_major:left", "blend:joy"} <= set(keys)
    assert len(keys) == len(set(keys)), "no parameter twice"
