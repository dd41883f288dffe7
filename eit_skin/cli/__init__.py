"""The ``eit-skin`` command line: ``main`` builds the parser from one module per sub-command.

Each command module has ``add_arguments(parser)`` and ``run(args) -> int`` and imports what is
heavy inside ``run``: ``patch`` (validate and draw a patch), ``simulate`` (frames and ground truth
from a touch scenario), ``reconstruct`` and ``classify`` (offline, through the node's per-frame
pipeline), ``frames`` (MCAP <-> npz), ``fake_device`` (a board on a pseudo-terminal),
``record_postures`` (references across a joint sweep), ``tune`` (choose the regularisation),
``run`` (the whole skin end to end), ``presses`` (record or simulate a labelled press
session), ``calibrate`` (fit a press localiser), ``locate`` (calibrated contact positions),
``fit_device`` (fit sheet conductance and contact impedance to a no-load frame),
``capture`` (a board's frames to an npz, without ROS), ``detect`` (which board is on a port),
``design`` (the skin designer in the browser; ``patch`` also imports drawings and predicts
accuracy); ``errors`` (how a command reports a failure it can name); ``options`` (the
options several commands share: patch, layer, ``--write``, a board's link).
"""
