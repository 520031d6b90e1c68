"""Lane-function helpers every concept shares: small dense linear algebra (:mod:`.linalg`),
element-wise copies between lane-state arrays (:mod:`.records`) and the canonical-form model of an
estimate (:mod:`.canonical`).

See :mod:`stcgym.lanes.compiled` for the lane-function convention. The compiled steps themselves
live with their concept: :mod:`stcgym.adaptive.estimation`, :mod:`stcgym.adaptive.control`,
:mod:`stcgym.adaptive.multivariable` and :mod:`stcgym.adaptive.regression`.
"""
