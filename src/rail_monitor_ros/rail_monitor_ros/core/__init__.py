"""Estimator cores: one module per method, plus the vehicle model and track spectra they use."""
