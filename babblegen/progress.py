"""A run's progress bar: it counts attempts when ``max_attempts`` can end the run before its generations do, and
generations otherwise (an unreachable attempt count would make it promise hours), with the counters beside it."""

from __future__ import annotations

from typing import Any

from babblegen.config import RunConfig


def counts_attempts(config: RunConfig) -> bool:
    """Whether ``max_attempts`` can end the run before its generations do (a generation attempts at most
    ``children`` movements, or ``population``, fewer when children repeat tried genomes)."""
    per_generation = config.noveb.population
    if config.explorer == "noveb":
        per_generation = max(per_generation, config.noveb.children)
    return config.max_attempts is not None and config.max_attempts < per_generation * config.noveb.generations


class Progress:
    """The bar of a run with ``counters`` (the run's, updated in place) and ``explorer`` (its archive size is
    shown); ``enabled=False`` shows nothing."""

    def __init__(self, config: RunConfig, counters: dict[str, int], explorer: Any, enabled: bool = True):
        self.counters, self.explorer = counters, explorer
        self.counts_attempts = counts_attempts(config)
        self.bar = None
        if not enabled:
            return
        from tqdm import tqdm

        if self.counts_attempts:
            total, initial, unit = config.max_attempts, counters["attempts"], "attempt"
        else:
            total, initial, unit = config.noveb.generations, counters["generations"], "gen"
        self.bar = tqdm(total=total, initial=initial, unit=unit, dynamic_ncols=True, smoothing=0.05)

    def attempt_written(self) -> None:
        if self.bar is not None and self.counts_attempts:
            self.bar.update(1)
            self._show_counts()

    def generation_told(self) -> None:
        if self.bar is not None and not self.counts_attempts:
            self.bar.update(1)
            self._show_counts()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def _show_counts(self) -> None:
        """The counters beside the bar, as of the attempt or generation it just counted."""
        c = self.counters
        self.bar.set_postfix(
            attempts=c["attempts"],
            episodes=c["executed"],
            contact=c["contacts"],
            archive=self.explorer.archive_size,
            refresh=False,
        )
