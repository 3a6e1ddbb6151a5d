"""Adversarial motion priors, task side: the motion library (reference clips) and the AMP observation."""
