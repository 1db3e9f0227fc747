"""Independent peers the package is checked and benchmarked against (OpenSees finite elements). The core never imports them."""
