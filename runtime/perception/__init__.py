"""CRAFT-E package."""
