"""Batch estimation: least squares, Cramer-Rao bound and sensitivities, input design, model selection."""
