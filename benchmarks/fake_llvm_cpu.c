/* Tells LLVM's users in this process another host CPU name: an LD_PRELOAD shim for
 * benchmarks/check_render_dispatch.py --llvm-cpus. lavapipe asks llvm::sys::getHostCPUName() which CPU to generate
 * shader code for; with BABBLEGEN_LLVM_CPU set this answers that name, otherwise LLVM's own answer. With
 * BABBLEGEN_LLVM_CPU_LOG set to a file, each answer is appended to it (proof that the question was asked).
 * Build: cc -shared -fPIC -O2 -o fake_llvm_cpu.so fake_llvm_cpu.c -ldl */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <link.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct { const char *data; size_t size; } StringRef; /* llvm::StringRef, returned in two registers */

static int find_llvm(struct dl_phdr_info *info, size_t size, void *found) {
  (void)size;
  if (strstr(info->dlpi_name, "libLLVM")) { *(const char **)found = info->dlpi_name; return 1; }
  return 0;
}

StringRef _ZN4llvm3sys14getHostCPUNameEv(void) {
  const char *name = getenv("BABBLEGEN_LLVM_CPU");
  StringRef answer = {"", 0};
  if (name && *name) {
    answer.data = name;
    answer.size = strlen(name);
  } else {
    const char *path = NULL;
    dl_iterate_phdr(find_llvm, &path);
    void *llvm = path ? dlopen(path, RTLD_NOLOAD | RTLD_LAZY) : NULL;
    StringRef (*own)(void) = llvm ? (StringRef (*)(void))dlsym(llvm, "_ZN4llvm3sys14getHostCPUNameEv") : NULL;
    if (own) answer = own();
  }
  const char *log = getenv("BABBLEGEN_LLVM_CPU_LOG");
  FILE *f = log && *log ? fopen(log, "a") : NULL;
  if (f) {
    fprintf(f, "%.*s\n", (int)answer.size, answer.data);
    fclose(f);
  }
  return answer;
}
