# Sourced by scripts/bundle.sh and scripts/bundle-test.sh: the shared libraries a bundle takes
# from the machine it runs on rather than carrying them. They are the C runtime: glibc's own
# objects (the loader and libc must come from one build, the machine's) and libgcc_s, which
# glibc itself loads (thread cancellation, unwinding) and every glibc system therefore has.
# is_c_runtime SONAME: true for those.
is_c_runtime() {
    case "$1" in
        linux-vdso.so.*|ld-linux*.so.*|libc.so.*|libm.so.*|libpthread.so.*|libdl.so.*|librt.so.*|\
        libresolv.so.*|libutil.so.*|libanl.so.*|libmvec.so.*|libnsl.so.*|libBrokenLocale.so.*|\
        libgcc_s.so.*) return 0 ;;
        *) return 1 ;;
    esac
}
