"""The rig's layers (core.layer protocol): MPEG-4 FAPs, SABiom muscles, and those to come."""
