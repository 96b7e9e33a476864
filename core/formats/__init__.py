"""File formats: meshes, landmarks, .fap, DPC, projects, and their shared text and atomic-write helpers."""
