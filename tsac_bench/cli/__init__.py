"""The ``tsac-bench`` command line: the application (``app``) and its commands, one module per
subject, registered in the order ``--help`` lists them: one instance (``solving``), batch runs
(``runs``), what is known of the optima (``references``), training (``training``)."""

# isort: off
from tsac_bench.cli import solving  # noqa: F401  (registers its commands)
from tsac_bench.cli import runs  # noqa: F401
from tsac_bench.cli import references  # noqa: F401
from tsac_bench.cli import training  # noqa: F401
# isort: on
from tsac_bench.cli.app import app


def main() -> None:
    app()
