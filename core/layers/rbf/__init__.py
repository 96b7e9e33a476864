"""RBF control-point deformation (thesis B §4.1.1): kernels, influence regions, the rig layer, emotions."""
