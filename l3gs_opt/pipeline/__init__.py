"""From a scene to an instance: bundle building (trainer), the paper's Eq. 1 splat utility, instances from bundles and synthetic ones.
"""
