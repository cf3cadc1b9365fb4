//! Whole-path tests live in `tests/`; this library only hosts them as a workspace member.
