"""Object models of the synthetic street: one module per family, one `<name>_parts(rng, ...)` function per model.

A model draws its size, shape and reflectivity from `rng` and returns its parts (`synthetic.parts`) in its own
frame: x forward, y left, z up from the ground contact at the origin. Where to put it is the street layout's
job (`synthetic.scene`). To add a model, write its function in the module of its family (or a new module
here) and place it from the layout.
"""
