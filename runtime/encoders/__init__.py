"""Encoders: a registry of name -> checksum-verified weights, one ``load()`` per backend."""
