"""Every thread, process, pool, queue and lock EVP's engines run with.

The core (geometry, vision, slam, vo, fusion) computes in the caller's thread and is handed what
it needs to run work beside tracking: a real map lock, the local-mapping thread, the helper process
for bundle adjustments, a helper thread for callables run at once. This package owns them, starts
them and closes them (``slam.build_slam`` for the SLAM engine), and the process each of the station's sessions runs its
pipeline in (``estimator_process``)."""
