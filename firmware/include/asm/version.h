/* The firmware's version: module-info reports it and the update image header carries it. */
#ifndef ASM_VERSION_H
#define ASM_VERSION_H
#ifndef ASM_FW_VERSION
#define ASM_FW_VERSION 0x000100u /* 0xMMmmpp: 0.1.0 */
#endif
#endif
