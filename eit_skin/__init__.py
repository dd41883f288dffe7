"""eit_skin: robot skin by Electrical Impedance Tomography.

The modules directly in this package are the numerical core and know nothing of
ROS; ``eit_skin.nodes`` holds the thin ROS 2 adapters and ``eit_skin.cli`` the
``eit-skin`` command.
"""

__version__ = "0.1.0"
