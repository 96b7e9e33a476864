"""MPEG-4 facial animation: FAP tables and units, the base template, the Facial Animation Table, .fap files."""
