"""Knowledge bundles on the robot: load and verify (``bundle``), signed single-file packages
(``package``), atomic installs with rollback (``install``), and discrimination diagnostics."""
