"""TSAC-OCF: the OCF game played by a transformer soft actor-critic policy: the environment
(`env`), the network (`net`), training (`sac`) and the allocator with its shipped policy
(`policy`). Importing this package loads nothing heavy; its modules load torch."""
