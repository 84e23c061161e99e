"""Road simulator: vehicle dynamics truth model, scenario reader, sensor synthesis."""
