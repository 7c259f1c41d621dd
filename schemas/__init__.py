"""Pydantic models of every CRAFT-E artifact, versioned by folder (``v1/``).

Both the compiler and the runtime import these; they depend on nothing but pydantic.
"""
