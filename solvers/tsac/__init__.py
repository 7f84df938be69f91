"""TSAC-OCF: the OCF game played by a transformer soft actor-critic policy: the policy's state
(`features`), the networks (`net`), training (`sac`), the deviation verifier (`verify`) and the
allocator with its shipped policy (`policy`). Importing this package loads nothing heavy; its
modules load torch."""
