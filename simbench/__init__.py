"""Bench tools, not nodes: the AX-12A servo emulator (:mod:`simbench.servo_sim`, a real serial peer
on a pseudo-terminal) and the simulated table it drives (:mod:`simbench.world`, a world file the
camera renders). Nodes use them only for ``port: sim`` and ``source.sim_bench``."""
