"""Studies: what train.py and evaluate.py print, plot and write (tables through `logging`, figures,
TensorBoard events, checkpoints, metrics.json), on top of the pure library below them."""
