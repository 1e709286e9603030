/* size_report.c: prints the RAM the core's state takes (a hosted program for `make size`;
 * not part of the firmware). */
#include <stdio.h>

#include "firmware.h"

int main(void)
{
    printf("sizeof(fw_state) = %lu bytes (of which the send queue %lu)\n",
           (unsigned long)sizeof(fw_state), (unsigned long)sizeof(((fw_state *)0)->tx));
    printf("sizeof(fl_deframer) = %lu bytes, sizeof(fl_message) = %lu bytes\n",
           (unsigned long)sizeof(fl_deframer), (unsigned long)sizeof(fl_message));
    return 0;
}
