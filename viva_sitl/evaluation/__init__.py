"""Perception, trials and scoring (landing benchmark): planned."""
