"""Distribution over Ray: the fan-out of particle simulations to shard actors, the shard
pools a server shares, and the watchdog that takes a server's processes down with it."""
