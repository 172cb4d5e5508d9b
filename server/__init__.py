"""The backend: the CAN <-> Zenoh bridge, the module runtime and the studio server."""
