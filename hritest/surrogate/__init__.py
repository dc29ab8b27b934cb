"""The torch surrogate of SAS / DSAS: the networks (:mod:`.networks`), their training
(:mod:`.model`), their fast inference form (:mod:`.inference`) and the constraint penalty the
inner loop adds (:mod:`.penalty`). Imported only by the surrogate-assisted search: torch is heavy."""
