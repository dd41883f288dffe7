"""The reconstruction methods a layer's ``solver.method`` can name (the one list of them).

* ``one_step``: linearised difference imaging with a smoothness prior
  (:mod:`eit_skin.inverse.one_step`, priors in :mod:`eit_skin.inverse.priors`);
* ``greit``: the one-step matrix trained on simulated targets (:mod:`eit_skin.inverse.greit`);
  it has no prior of its own;
* ``gauss_newton``: iterative regularised Gauss-Newton for large contrasts
  (:mod:`eit_skin.inverse.gauss_newton`), with a prior.
"""

from __future__ import annotations

METHODS: tuple[str, ...] = ("one_step", "greit", "gauss_newton")

#: Methods that use ``solver.prior``.
METHODS_WITH_PRIOR: tuple[str, ...] = ("one_step", "gauss_newton")
