"""policy-composer: compose diverse controllers with a learned goal score (RA-L 2020), in ManiSkill."""

__version__ = "0.1.0"
