"""Data in: the dataset format's parser, the per-frame label dataset and the datamanager config."""
