"""Estimation: the filters (MEKF, UKF, RateMEKF), the step-by-step estimator and the
GTSAM smoother. Imports ``adfusion.starid`` only; never the application or the harness."""
