"""What an algorithm appends to the environment's observation (the told mode, neighbour messages, the global state, the
belief): the vector wrappers' base and the mixins of the algorithms that wrap (``wrapping``), the features extractor
that splits the appended values off (``extractor``) and the start of the weights that read them
(``initialization``). The wrappers themselves live with what they append."""
