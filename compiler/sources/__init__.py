"""Knowledge sources behind one interface each, cache-first: LLM, ConceptNet, overrides."""
