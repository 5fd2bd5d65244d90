"""Rendering results as HTML, Markdown and PNG: the only place that imports matplotlib."""
