"""Frequency analysis: spectrum operators (numpy specification), compiled chains, occlusion grid."""
