"""Reporting: data loaded from a results store, statistics, tables (Markdown and LaTeX)
and figures. Depends on the batch layer only through the store it reads."""
