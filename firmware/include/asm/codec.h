/* Values on the wire (docs/protocol.md section 2): whether bytes are a valid value of the codec a descriptor
 * describes. The node checks every remote SET with its object's descriptor, so an object's type is written once.
 * (JSON values are checked as UTF-8 only: a module parses no JSON.) */
#ifndef ASM_CODEC_H
#define ASM_CODEC_H

#include <stddef.h>
#include <stdint.h>

/* ASM_OK when ``data`` is exactly one value of the codec ``descriptor`` describes, else ASM_E_FORMAT. */
int asm_codec_check(const uint8_t *descriptor, size_t descriptor_length, const uint8_t *data, size_t length);
/* Strict UTF-8 (no overlong forms, no surrogates, nothing beyond U+10FFFF), as Python decodes it. */
int asm_utf8_valid(const uint8_t *s, size_t length);

#endif
