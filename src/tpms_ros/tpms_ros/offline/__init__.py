"""Offline evaluation, tuning and plots over recordings and simulations."""
