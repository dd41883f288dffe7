"""eit_skin: robot skin by Electrical Impedance Tomography.

The numerical core knows nothing of ROS: ``patch`` (configs), ``fem`` (forward model),
``inverse`` (reconstruction), ``pipeline`` (one layer's frame -> images), ``hardware``
(boards), ``io`` (recordings), ``sim`` (simulator), ``touch`` (contacts and events).
``ros`` holds the thin ROS 2 adapters and ``cli`` the ``eit-skin`` command.
docs/architecture.md draws the data's way through them.
"""

__version__ = "0.1.0"
