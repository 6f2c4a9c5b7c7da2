fn main() {
    println!("amx {} avx512bf16 {}", nst3d_core::bf16::amx::available(), nst3d_core::bf16::avx512_bf16_available());
    #[cfg(target_arch = "x86_64")]
    {
        let r = std::arch::x86_64::__cpuid_count(7, 0);
        println!("edx {:032b}", r.edx);
        println!("bf16 detect {}", std::arch::is_x86_feature_detected!("avx512bf16"));
    }
    println!("{:?} {:?}", nst3d_core::precision::hardware(), nst3d_core::precision::path());
}
