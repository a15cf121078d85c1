"""Tasks: what an episode asks of a body (observation, reward, termination), one file each,
found by name through `registry.make_env`."""
