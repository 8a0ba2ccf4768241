"""Evaluation tools (convergence reports, metrics): not part of the shipped extension."""
