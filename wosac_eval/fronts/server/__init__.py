"""The HTTP scoring service (`wosac-eval serve`): API, job store, workers, web page."""
