"""Lights: the light table, emission sampling, next-event estimation, lights seen by rays."""
