"""The canonical-form model of an estimate, shared by the estimators' and the controllers' lane
functions (:mod:`.canonical`: companion matrices, integral augmentation).

See :mod:`stcgym.lanes.compiled` for the lane-function convention and :mod:`stcgym.lanes.linalg`
for the small dense linear algebra and copies every lane function uses. The compiled steps
themselves live with their concept: :mod:`stcgym.adaptive.estimation`,
:mod:`stcgym.adaptive.control`, :mod:`stcgym.adaptive.multivariable` and
:mod:`stcgym.adaptive.regression`.
"""
