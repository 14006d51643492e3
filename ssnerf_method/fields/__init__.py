"""The SS-NeRF field: shared position encoder F_enc and the two decoders F_dec^v and F_dec^nv."""
