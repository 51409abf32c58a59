"""Training: config to data and model, the optimisation loop, checkpoints and resume.

Not built yet: see the project's issues.
"""
