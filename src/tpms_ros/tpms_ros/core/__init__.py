"""Estimator cores of the road domain: one module per method, shared message-free types."""
