"""What the viewer and `ns-render` show: the model's display outputs and its semantics panel."""
