"""torchrl-mbe's Hydra launcher plugin: ``hydra/launcher=population`` (``conf/hydra/launcher/population.yaml``)."""
