"""One thin script per DVC stage: parse paths, load, call the library, save."""
