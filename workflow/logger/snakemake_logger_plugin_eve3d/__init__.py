"""Snakemake logger plugin ``eve3d``: registers :class:`.progress.ProgressHandler`."""
from dataclasses import dataclass, field
from typing import Optional

from snakemake_interface_logger_plugins.base import LogHandlerBase
from snakemake_interface_logger_plugins.settings import LogHandlerSettingsBase


@dataclass
class LogHandlerSettings(LogHandlerSettingsBase):
    interval: Optional[float] = field(
        default=5.0, metadata={"help": "Seconds between two progress lines of one running job"})


class LogHandler(LogHandlerBase):
    def __post_init__(self) -> None:
        import sys

        from snakemake.logging import DefaultFormatter

        from snakemake_logger_plugin_eve3d.progress import (
            ProgressHandler,  # imported here: Snakemake imports every plugin at start
        )

        formatter = DefaultFormatter(self.common_settings.quiet, self.common_settings.show_failed_logs)
        self.progress = ProgressHandler(sys.stdout if self.common_settings.stdout else sys.stderr,
                                        (self.settings.interval if self.settings else None) or 5.0, formatter)

    def emit(self, record) -> None:
        self.progress.emit(record)

    def close(self) -> None:
        self.progress.close()
        super().close()

    @property
    def writes_to_stream(self) -> bool:
        return True

    @property
    def writes_to_file(self) -> bool:
        return False

    @property
    def has_filter(self) -> bool:
        return True  # it shows job events, warnings and errors only

    @property
    def has_formatter(self) -> bool:
        return True

    @property
    def needs_rulegraph(self) -> bool:
        return False
