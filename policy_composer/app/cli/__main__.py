import sys

from policy_composer.app.cli import main

sys.exit(main())
