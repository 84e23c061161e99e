"""Offline evaluation, runners, metrics and plots."""
