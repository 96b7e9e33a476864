"""Waters vector muscles (thesis B §4.1.2, eqs. 4.16-4.19; Waters 1987): model, rig layer and the inverse."""
