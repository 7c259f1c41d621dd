"""Perception: RGB-D observations, table-plane fitting and class-agnostic ROI segmentation.

Free of simulator imports, so the same code runs on frames from a real camera.
"""
