"""Interactive viewer of 3DGS PLYs in the browser (``plantdreamer view``), built on viser.

``scene`` turns a PLY into what the browser draws (pure numpy, no viser); ``server`` serves
it. viser is the optional ``viewer`` extra: only ``server`` imports it.
"""

HOST = "127.0.0.1"  # the viewer is served to this machine only
DEFAULT_PORT = 8080
