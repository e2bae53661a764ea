"""Policies: the Policy interface (`base`), the registry and factories (`registry`), policies of installed
packages (`plugins`, entry-point group `gazereg.policies`), the reference VLA (`vla`).

    from gazereg.policies import Policy, PolicyConfig, register_policy, make_policy, load_policy

See `gazereg.policies.base` for what a policy implements and `gazereg.policies.registry` for registration.
"""

from gazereg.policies.base import Policy, PolicyConfig, PolicyTokenizer
from gazereg.policies.registry import (
    POLICIES,
    POLICY_CHOICE,
    PolicyRegistry,
    available_policies,
    load_policy,
    make_policy,
    policy_class,
    policy_config_class,
    register_policy,
    unregister_policy,
)

__all__ = [
    "POLICIES",
    "POLICY_CHOICE",
    "Policy",
    "PolicyConfig",
    "PolicyRegistry",
    "PolicyTokenizer",
    "available_policies",
    "load_policy",
    "make_policy",
    "policy_class",
    "policy_config_class",
    "register_policy",
    "unregister_policy",
]
