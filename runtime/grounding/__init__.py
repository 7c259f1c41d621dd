"""Grounding a verb in a scene: the settings (``settings``), the paper's energies (``energies``),
the ``Grounder`` (``grounder``), open-world inference (``open_world``), explanations and plots."""
