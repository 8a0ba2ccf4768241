"""Stochastic progressive photon mapping stages: visible points, hash grid, photon pass, update, film."""
