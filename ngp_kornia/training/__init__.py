"""Training: LightningModules, losses and DataModules. Knows the models and the data; nothing imports it back."""

__all__: list[str] = []
