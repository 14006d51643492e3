"""The embedded default SS-NeRF scene: a procedural furnished room, its ray caster and the dataset generator."""
