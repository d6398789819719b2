//! Integration tests of vibrocomp: one binary, a module per topic.
