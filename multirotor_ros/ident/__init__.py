"""Identification of model parameters from flight logs (pure: numpy and scipy, no ROS).

Offline (``multirotor identify``):

- :func:`.identify.identify` -> :class:`~multirotor_ros.ident.identify.IdentificationResult`:
  fit k_f and the parameters of chosen effects (effects.md names) to a flight-log CSV, with standard
  deviations, identifiability verdicts and the acceleration error before and after.
- :mod:`.samples`: a log made ready for fitting (derived motion, measurement filter, usable samples).
- :mod:`.regressors`: y = Phi theta of the equation-error form, built from the model itself
  (:class:`~multirotor_ros.ident.regressors.ForceRegressor`, also used by the online identifier).
- :mod:`.fit`: least squares, searches of the non-linear parameters, covariance, identifiability.
- :mod:`.metrics`, :mod:`.plots`, :mod:`.parameters`, :mod:`.excitation` (informative flight schedules).

Online: :mod:`.rls` (recursive least squares for the identifier node). Bench data of seed 2: :mod:`.bench`.
Submodules are imported explicitly, so that importing one does not load the others (scipy, matplotlib).
"""
