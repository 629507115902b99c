import sys

from reneus_mi.capture.command import main

sys.exit(main())
