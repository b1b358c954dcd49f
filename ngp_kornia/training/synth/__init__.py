"""The procedural renderer of Manhattan and Atlanta worlds: scenes, facades, interiors, layouts, clutter, painter."""

__all__: list[str] = []
