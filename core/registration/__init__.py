"""Scan registration (thesis A ch. 2-3): scan input and clean-up, virtual scanner and synthetic
database, rigid ICP, curvature/HK maps, texture candidates, structural matching.

Modules (import them directly; this package imports nothing heavy on its own):

- ``range_image``     depth/xyz grid + colour image -> textured Face
- ``cleanup``         hole filling, small-component removal, spike smoothing (A §2.2)
- ``virtual_scanner`` any textured Face -> single-view range scan with ground-truth landmarks
- ``synthetic``       the 30 people x 7 poses protocol database, generated and cached on demand
- ``icp``             rigid Besl-McKay ICP (trimmed, KD-tree)
- ``curvature``       mean/Gaussian curvature, HK classes and colours, Colombo seeds (A §3.2)
- ``candidates``      Shi-Tomasi texture candidates lifted to 3-D; geometry-only fallback
"""
