"""Prompt templates of the knowledge compiler (``<id>.<version>.md``), shipped as package data.

This folder is the design card's top-level ``prompts/``; it is a package only so that an installed
wheel carries the templates (``craft_e.prompts``) and ``compiler.prompts`` finds them through
``importlib.resources`` rather than through the location of a source checkout.
"""
