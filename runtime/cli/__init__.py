"""``craft``: one thin module per command group over the library; ``main`` assembles them."""
