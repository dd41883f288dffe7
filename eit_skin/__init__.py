"""eit_skin: robot skin by Electrical Impedance Tomography.

The numerical core knows nothing of ROS: ``patch`` (configs), ``fem`` (forward model),
``inverse`` (reconstruction), ``pipeline`` (one layer's frame -> images), ``hardware``
(boards), ``io`` (recordings), ``sim`` (simulator), ``touch`` (contacts and events).
``ros`` holds the thin ROS 2 adapters and ``cli`` the ``eit-skin`` command.
docs/architecture.md draws the data's way through them.
"""

__version__ = "0.1.0"


def lazy_exports(package: str, exports: dict[str, str]):
    """``__getattr__`` and ``__dir__`` for a subpackage that re-exports names of its modules.

    ``exports`` maps a public name to the module of ``package`` that defines it; the module is
    imported on first use, so importing one module never imports its whole subpackage (and
    subpackages cannot form import cycles through their ``__init__``).
    """
    import importlib

    def __getattr__(name: str):  # noqa: N807 (module-level __getattr__, PEP 562)
        if name in exports:
            return getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:  # noqa: N807
        return sorted(exports)

    return __getattr__, __dir__
