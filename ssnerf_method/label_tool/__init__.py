"""`ssnerf-label`: derive property labels for a posed nerfstudio dataset with `ssnerf_method.label_makers`' makers."""
