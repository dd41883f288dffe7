"""Sub-commands of the ``eit-skin`` command line, one module each."""
