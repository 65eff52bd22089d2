//! The model as users name it: the terms of a model spec.

pub mod spec;
