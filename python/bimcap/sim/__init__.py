"""The synthetic world: parametric IFC building generator, sensor simulator, drift generator."""
