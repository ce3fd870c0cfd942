"""The optimisation: the training loop, the validation that ranks its candidates, the losses, the
first majorise-minimise steps, AdamW, the learning-rate schedule and the loop's progress events."""
