"""Materials: the table of lobes, BSDF evaluation and sampling, compiled fast path."""
