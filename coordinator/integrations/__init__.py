"""What the service speaks besides its own API: the Gymnasium view of a domain, TensorBoard
logging, MCAP export, and scene pictures (frames)."""
