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

#: Noise figure the hyperparameter is chosen for when neither ``h`` nor a noise figure is
#: given (:func:`eit_skin.inverse.hyperparameter.choose_by_noise_figure`), one per method:
DEFAULT_NOISE_FIGURE: dict[str, float] = {
    # the noise-figure study of docs/reconstruction.md: with the Laplace prior NF 0.3 keeps
    # the position error (2.3 % R) and resolution (0.23) of NF 0.1-0.2 at less ringing, NF 1
    # blurs (RES 0.28) and moves targets (PE 2.6 % R); the value config/elbow.yaml ships
    "one_step": 0.3,
    # config/arm.yaml and face.yaml: test_accuracy.py meets max PE <= 2 % R, ringing <= 0.2
    # and resolution <= pyEIT JAC's 0.248 at this value
    "greit": 0.13,
    # chosen on its first linearised step, which is the one_step matrix with the same prior
    "gauss_newton": 0.3,
}
