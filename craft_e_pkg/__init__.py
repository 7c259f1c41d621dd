"""CRAFT-E: neuro-symbolic affordance grounding (compiler, runtime, testbed)."""

__version__ = "0.1.0"
