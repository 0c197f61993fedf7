"""The reproduce and evaluate pipelines: tables, report and figures (matplotlib imported only
where figures are drawn)."""
