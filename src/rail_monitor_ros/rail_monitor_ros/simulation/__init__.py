"""Rail simulator, scenario reader and track profile synthesis."""
