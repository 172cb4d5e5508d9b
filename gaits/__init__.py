"""Gaits: the gait file format, validation, control tables and the gait library (gaits/library/*.toml)."""
